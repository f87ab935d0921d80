"""WoodenHaptics (open 3-DOF, mbed LPC1768 over USB HID): report codec and kinematics (``protocol``), driver (``driver``)."""
