"""The device firmware: C sources (``hfam_fw.c``, ``hfam_protocol.[ch]``), their Python mirror and the emulator.

``logic``     the on-device renderer the firmware runs, in plain scalar Python (mirrors ``hfam_fw.c``)
``emulator``  a firmware emulator on a pseudo-terminal or in-process HID seam (``python -m devices emulate``)
"""
