"""Synthetic data sets at scale: specs, items and the Dask engine (``shinysim dataset``).

* :mod:`shinysim.datasets.spec`: the JSON spec, validated; every item
  resolved from (spec, index, seed) alone;
* :mod:`shinysim.datasets.items`: one item's scene, renders and files (what a
  worker runs);
* :mod:`shinysim.datasets.engine`: the run on a Dask cluster, resumable, with
  its manifest (:func:`run_dataset`);
* :mod:`shinysim.datasets.export`: a data set as DiLiGenT folders.

Importing this package loads none of its parts, nor the renderer or Dask.
"""

from .._shared import lazy_face

__all__ = lazy_face(__name__, (
    "engine", "export", "items", "spec"), {
    "engine": ("DATASET_FORMAT", "run_dataset", "build_one", "read_manifest", "prepare_folder", "default_workers"),
    "export": ("export_diligent_folders",),
    "items": ("ITEM_FORMAT", "item_path", "render_item", "write_item", "file_digests", "file_sha256", "reset_cache"),
    "spec": ("SPEC_FORMAT", "GROUP_DEFAULTS", "DatasetSpec", "load_spec", "parse_spec", "resolve_item",
             "spec_diff", "RIG_PRESETS", "OBJECT_KINDS", "build_rig", "MATERIAL_KINDS", "MAX_ITEMS"),
})
