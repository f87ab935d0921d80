"""3D Systems Touch / Phantom through OpenHaptics' HD API (ctypes; the vendor's library is optional)."""
