"""The brightness conventions shared by the simulator, the losses and the evaluation.

An event sensor responds to changes of L = log(I + LOG_EPS) for linear intensity I in [0, 1].
LOG_EPS keeps black pixels finite (log 1e-3 = -6.9) and bounds dL/dI by 1000, so a few dark
pixels cannot dominate a gradient; it plays the role of a real sensor's dark current.
A monochrome sensor looking at an RGB scene sees its Rec. 709 luma.
"""

from __future__ import annotations

import numpy as np

LOG_EPS = 1e-3
LUMA = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
