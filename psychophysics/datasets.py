"""Published psychometric data sets, as counts per level: for checking fits against other software.

Each is ``(levels, n, k)``: stimulus levels, trials and correct (or "yes") answers per level.

* :data:`BLISS_1935`: beetles killed by carbon disulphide, the classic dose-response data (Bliss 1935,
  *Ann. Appl. Biol.* 22:134-167, table 6; re-used by every GLM text, e.g. Dobson & Barnett, *An Introduction
  to Generalized Linear Models*, table 7.2): log10 dose (mg/l), beetles, beetles killed. A yes/no data set
  (no guessing floor).
* :data:`PSIGNIFIT_DEMO`: the 2AFC data of psignifit 4's documentation and demos (Schütt, Harmeling, Macke &
  Wichmann 2016, *Vision Res.* 122:105-123; the Python package's basic-usage page): stimulus contrast,
  trials and correct answers; 90 trials at each of 13 levels.
"""

from __future__ import annotations

import numpy as np

BLISS_1935 = (np.array([1.6907, 1.7242, 1.7552, 1.7842, 1.8113, 1.8369, 1.8610, 1.8839]),
              np.array([59.0, 60, 62, 56, 63, 59, 62, 60]),
              np.array([6.0, 13, 18, 28, 52, 53, 61, 60]))

PSIGNIFIT_DEMO = (np.array([0.0010, 0.0015, 0.0020, 0.0025, 0.0030, 0.0035, 0.0040, 0.0045, 0.0050, 0.0060,
                            0.0070, 0.0080, 0.0100]),
                  np.full(13, 90.0),
                  np.array([45.0, 50, 44, 44, 52, 53, 62, 64, 76, 79, 88, 90, 90]))

#: name -> (data, alternatives, what it is)
DATASETS = {"bliss1935": (BLISS_1935, 1, "Bliss (1935) beetle mortality, yes/no"),
            "psignifit_demo": (PSIGNIFIT_DEMO, 2, "psignifit 4 demo data, 2AFC")}
