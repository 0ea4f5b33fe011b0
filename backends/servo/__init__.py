"""Servo buses, protocols, safety and emulators behind the dynamixel and maestro backends."""
