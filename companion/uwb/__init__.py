"""companion.uwb"""
