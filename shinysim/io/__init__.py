"""Every file format shinysim reads and writes (``docs/file-format.md`` specifies each).

* :mod:`~shinysim.io.stack`: scan folders' ``stack.exr`` and ``truth.exr``
  (:class:`Stack`, :class:`Truth`), the contract between simulation and
  reconstruction; its names are this package's own;
* :mod:`~shinysim.io.document`: the one reader of text and JSON files (size
  cap, byte-order mark, UTF-8, errors naming the file);
* :mod:`~shinysim.io.rig`: ``rig.json`` (:func:`load_rig`);
* :mod:`~shinysim.io.frames`: ordinary camera frames (PNG, TIFF, TGA, JPEG,
  BMP, OpenEXR) as a stack;
* :mod:`~shinysim.io.table`: ``highlights.csv``;
* :mod:`~shinysim.io.coded`: coded scans (``coded.npz``, ``code.json``) and
  :class:`~shinysim.io.coded.CodedStack`;
* :mod:`~shinysim.io.matches`: a stereo scan's ``matches.csv``;
* :mod:`~shinysim.io.calibration`: ``placements.json`` and ``spheres.json``;
* :mod:`~shinysim.io.diligent`: DiLiGenT photometric-stereo folders;
* :mod:`~shinysim.io.sofast`: Sandia OpenCSP SOFAST deflectometry files (HDF5 and JSON), read in
  millimetres.

Readers check everything they rely on and raise the package's own errors
(:mod:`shinysim.errors`) naming the file and the field; writers never replace
a file unless asked to and write through a temporary file.
"""

from . import stack
from .rig import MAX_RIG_BYTES, load_rig
from .stack import *  # noqa: F403 - the stack and truth files' names are the package's own

__all__ = [*stack.__all__, "MAX_RIG_BYTES", "load_rig"]
