"""Images as a camera writes them, turned into dot centres: the input of every model (paper §3).

``robust``
    robust statistics of pixels (medians of integers, the median absolute deviation);
``overlay``
    a camera's text strip: found, left out of the contrast mesh, painted over for the centres;
``dots``
    finding a plate's dots: a threshold sweep over the local contrast, hot pixels, the local search;
``markers``
    the plate's markers: shapes off the lattice, shapes joined to a dot, blobs in a two-level plate's holes;
``streaks``
    window streaks read along the columns through each dot;
``centres``
    their sub-pixel centres (``moments``, ``ellipse``, ``edges``, ``fit``, ``symmetry``);
``lattice``
    numbering them on the plate's fitted lattice (its size, or its markers);
``extract``
    one image, end to end, with a report of what was found and rejected and why;
``boards``
    the targets OpenCV detects itself: chessboards, circle grids, ChArUco boards;
``imageset``
    a whole set's images into one ``points.csv``, one numbering for the set.
"""

from .extract import ImageDots, extract_image
from .imageset import extract_set

__all__ = ["ImageDots", "extract_image", "extract_set"]
