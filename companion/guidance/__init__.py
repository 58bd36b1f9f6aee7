"""companion.guidance"""
