"""Wire formats of the serial devices, as pure codecs (bytes and strings in, values out; no pyserial, no I/O).

Each protocol lives here once, specified in ``docs/devices.md``, and is imported by both sides: the driver in
``nodes/drivers/`` and the emulator in ``emulators/``. Tests check it against byte strings written from the spec.
"""
