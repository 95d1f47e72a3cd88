"""Virtual instruments with truth: the stereo rigs of :mod:`slmlab.virtual.rigs` beside the CMO microscope
(:mod:`slmlab.microscope`), and the calibration designs that image them (:mod:`slmlab.virtual.designs`)."""
