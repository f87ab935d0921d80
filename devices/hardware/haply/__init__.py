"""Haply Inverse3 (3-DOF, USB CDC serial): the wire codec (``protocol``) and the driver (``driver``)."""
