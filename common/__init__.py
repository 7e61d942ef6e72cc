"""The lowest layer: what every package of kanagen may import, importing nothing of kanagen —
:mod:`~kanagen.common.lazy` (names a package imports on first use) and
:mod:`~kanagen.common.slack` (the value of an inequality's slack, appendix F, which the spec
reader and the runtime both compute). The runtime needs nothing of the spec reader."""
