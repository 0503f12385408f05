"""The benchmark suite behind ``python -m diana_lab.bench``: every speed figure of the platform, side by side.

One module per area registers its measurements (:mod:`.sensing`, :mod:`.dynamics`, :mod:`.envs`,
:mod:`.training`, :mod:`.deploy`); :mod:`.suite` runs them and :mod:`.report` prints and writes the result.
``benchmarks/README.md`` documents every key, its target and the anchors it is compared with.
"""

from diana_lab.benchmarks.suite import run

__all__ = ["run"]
