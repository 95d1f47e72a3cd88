"""Third-party calibration data: converters into slmlab's interchange format (``converters``)."""
