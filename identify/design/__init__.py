"""calbench.identify.design — design of experiments (paper §5).

candidates (feasible configurations and their exact information blocks), candidate_file (the
NPZ other tools read and write), criteria (A, D, AD, pose), exchange (the discrete optimiser),
certificate (approximate optimal designs and the bound that certifies a plan), selection (rows
chosen and certified, on any blocks), plan (the whole pipeline and the runnable plan), study
(the paper's Tables 1-4 and Figs. 7-8), threads (BLAS pinning for the small algebra).
"""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
