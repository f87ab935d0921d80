"""Novint Falcon (3-DOF delta, FTDI USB): packet codec (``protocol``), libnifalcon's kinematics (``kinematics``),
the FTDI link over pyftdi with the firmware upload (``link``) and the driver (``driver``)."""
