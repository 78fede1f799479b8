"""Choosing the Mitsuba variant: cuda, then llvm, then scalar.

``llvm_*`` variants need an LLVM shared library that drjit 1.5 accepts (on
Debian 12: the ``libllvm19`` package; the default libLLVM 14/15 do not
work). Without it Mitsuba still runs its ``scalar_*`` variants, much more
slowly; :func:`choose_variant` says so in the reason it returns.
"""

from __future__ import annotations

import os

from .._shared import signals_held
from ..errors import OptionError, ShinysimError, did_you_mean

__all__ = ["VARIANT_PREFERENCE", "COLOUR_VARIANT_PREFERENCE", "choose_variant", "is_vectorized", "is_colour_variant",
           "active_variant"]

#: Fastest first. Scalar Mitsuba ships RGB but not mono.
VARIANT_PREFERENCE = ("cuda_ad_mono", "llvm_ad_mono", "scalar_rgb")
#: Variants that render in colour (linear RGB), fastest first.
COLOUR_VARIANT_PREFERENCE = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")

_ENV = "SHINYSIM_VARIANT"
#: The JIT backend of each kind of variant, and what a missing one is called.
_BACKENDS = {"cuda": ("CUDA", "no CUDA GPU"), "llvm": ("LLVM", "no usable LLVM library (install Debian's libllvm19)")}


def is_vectorized(variant):
    """True for JIT (cuda/llvm) variants that trace many rays per call."""
    return variant.startswith(("cuda", "llvm"))


def is_colour_variant(variant):
    """True for the RGB variants (``*_rgb``), whose images have R, G and B channels."""
    return str(variant).endswith("_rgb")


def active_variant():
    """The Mitsuba variant active in this process, None when Mitsuba is not loaded or none is set.

    Imports nothing: a process that has not loaded Mitsuba has no variant.
    """
    import sys

    mi = sys.modules.get("mitsuba")
    if mi is None:
        return None
    try:
        return mi.variant()
    except Exception:  # a half-initialised import
        return None


def choose_variant(preferred=None, *, colour=False):
    """Pick and activate a Mitsuba variant.

    Parameters
    ----------
    preferred : str, optional
        A variant name to force (also read from the ``SHINYSIM_VARIANT``
        environment variable). Without it the first usable variant of
        :data:`VARIANT_PREFERENCE` is taken.
    colour : bool
        Choose among the RGB variants (:data:`COLOUR_VARIANT_PREFERENCE`);
        a ``preferred`` one must be RGB, and ``SHINYSIM_VARIANT`` is used
        only when it names an RGB variant.

    Returns
    -------
    variant : str
    reason : str
        One line saying what was chosen and why (e.g. why llvm was not).

    Raises
    ------
    OptionError
        If the preferred variant is unknown or cannot run here (a ``ValueError``).
    ShinysimError
        If the renderer is not installed, or no variant can run here.
    """
    # Ctrl-C during these imports would leave the C extensions half initialised
    # (and the interpreter aborting at exit): it is held until they are done
    with signals_held():
        try:
            import drjit as dr
            import mitsuba as mi
        except ModuleNotFoundError as exc:
            raise ShinysimError(f"rendering needs the render extra (pip install 'shinysim[render]'): {exc}") from None
        except ImportError as exc:
            raise ShinysimError(f"the renderer failed to load: {exc}") from None
        return _choose(dr, mi, preferred, colour)


def _choose(dr, mi, preferred, colour=False):
    """The body of :func:`choose_variant`, with the renderer imported."""
    if colour:
        if preferred is not None and not is_colour_variant(preferred):
            raise OptionError(f"Mitsuba variant {preferred!r} does not render in colour; choose an RGB variant "
                              f"({', '.join(COLOUR_VARIANT_PREFERENCE)})", field="variant")
        env = os.environ.get(_ENV)
        preferred = preferred or (env if env and is_colour_variant(env) else None)
    else:
        preferred = preferred or os.environ.get(_ENV) or None
    available = mi.variants()
    if preferred is not None:
        if preferred not in available:
            raise OptionError(f"Mitsuba variant {preferred!r} is not available here; choose one of "
                              f"{', '.join(available)}{did_you_mean(preferred, available)}", field="variant")
        backend = _BACKENDS.get(preferred.split("_")[0], (None,))[0]
        if backend is not None and not dr.has_backend(getattr(dr.JitBackend, backend)):
            raise OptionError(f"Mitsuba variant {preferred!r} needs a {backend} backend, which is not usable here",
                              field="variant")
        mi.set_variant(preferred)
        return preferred, f"using Mitsuba variant {preferred} (requested)"
    skipped = []
    for name in (COLOUR_VARIANT_PREFERENCE if colour else VARIANT_PREFERENCE):
        if name not in available:
            skipped.append(f"{name} not compiled")
            continue
        kind = name.split("_")[0]
        if kind in _BACKENDS and not dr.has_backend(getattr(dr.JitBackend, _BACKENDS[kind][0])):
            skipped.append(_BACKENDS[kind][1])
            continue
        mi.set_variant(name)
        why = f" ({'; '.join(skipped)})" if skipped else ""
        slow = " -- scalar rendering is slow" if kind == "scalar" else ""
        return name, f"using Mitsuba variant {name}{why}{slow}"
    raise ShinysimError(f"no usable Mitsuba variant among {', '.join(available)}")
