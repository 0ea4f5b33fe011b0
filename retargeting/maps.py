"""Channel maps: canonical motion arrays to raw joint values, vectorised over time.

Every term of every joint becomes one column of a (T, K) matrix of raw quantities (an Euler angle
of a composed rotation, a blendshape weight, a root coordinate); mapped terms go through
``np.interp``; one (K, J) weight matrix then sums terms into joints, and gain, direction and offset
finish the job. A clip of thousands of frames is a handful of array operations.
"""

from __future__ import annotations

import numpy as np

from convodrive.motion.channels import BLENDSHAPE_INDEX
from convodrive.motion.rotations import axis_angle_to_matrix, matrix_to_euler
from convodrive.motion.skeleton import JOINT_INDEX
from retargeting_compat import *  # noqa: F401,F403  (placeholder removed below)
