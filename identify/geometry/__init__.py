"""calbench.identify.geometry — geometric calibration from absolute readings.

chain (a serial arm as fixed frames and revolute joints, the UR10 from its DH table, gravity
torques), model (the complete model of a reading: link frames, joint offsets, joint compliance
under self-weight, probe and base frames, with its exact Jacobian), fit (the base set from the
SVD, the least-squares fit, held-out validation), mjcf (a chain, e.g. a calibrated one, as a
calbench MJCF, and a serial calbench MJCF as a chain), run (`calbench identify LOG --geometry`).
"""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
