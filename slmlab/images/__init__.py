"""Images as a camera writes them, turned into dot centres: the input of every model (paper §3).

``dots``
    finding a plate's dots and refining their centres to sub-pixel accuracy;
``lattice``
    numbering them on the plate's lattice (its size, or its markers);
``extract``
    one image, end to end;
``boards``
    the targets OpenCV detects itself: chessboards, circle grids, ChArUco boards;
``imageset``
    a whole set's images into one ``points.csv``, one numbering for the set.
"""

from .extract import ImageDots, extract_image
from .imageset import extract_set

__all__ = ["ImageDots", "extract_image", "extract_set"]
