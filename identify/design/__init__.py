"""calbench.identify.design — design of experiments (paper §5).

candidates (feasible configurations, their exact information blocks, and the NPZ other tools
read and write), criteria (A, D, AD, pose), exchange (the discrete optimiser), certificate
(approximate optimal designs and the bound that certifies a plan), selection (rows chosen and
certified, on any blocks), plan (the pipeline and the runnable plan), run (`calbench design` as
one library call), study (the paper's Tables 1-4 and Figs. 7-8).
"""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
