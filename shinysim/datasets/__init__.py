"""Synthetic data sets at scale: specs, items and the Dask engine (``shinysim dataset``).

* :mod:`shinysim.datasets.spec`: the JSON spec, validated; every item
  resolved from (spec, index, seed) alone;
* :mod:`shinysim.datasets.items`: one item's scene, renders and files (what a
  worker runs);
* :mod:`shinysim.datasets.engine`: the run on a Dask cluster, resumable, with
  its manifest.

Importing this package loads neither the renderer nor Dask.
"""

from .spec import SPEC_FORMAT, DatasetSpec, load_spec, parse_spec, resolve_item

__all__ = ["SPEC_FORMAT", "DatasetSpec", "load_spec", "parse_spec", "resolve_item"]
