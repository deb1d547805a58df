"""The probe: the fibre-optic reader, the pressure regulator controller, the camera tracker and the stiffness estimators that turn their readings into stiffness samples."""
