"""companion.telemetry"""
