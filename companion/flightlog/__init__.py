"""companion.flightlog"""
