"""Studies that run the package end to end on the virtual microscope and on real rigs.

``paper_runs``
    the paper's estimates over repeated simulations (Tables 2–4);
``workspace``
    beyond the paper: the default model against the noise floor over the whole workspace;
``extraction``
    extraction accuracy against the virtual microscope's truth;
``realrigs``
    real rigs and known targets: images to 3D.
"""
