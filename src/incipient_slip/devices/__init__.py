"""Protocol code shared by a device node and its emulator, and the emulators themselves.

`biotac` holds the BioTac SPI word layer and the USB bridge's frame format; `biotac_emulator`
is a byte-level BioTac behind an emulated bridge on a pty. Each emulator speaks exactly what
the real device speaks, so the device node cannot tell it from the hardware.
"""
