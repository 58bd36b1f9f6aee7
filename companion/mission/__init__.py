"""companion.mission"""
