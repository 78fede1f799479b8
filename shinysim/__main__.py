"""``python -m shinysim``: the ``shinysim`` command (:func:`shinysim.cli.run`)."""

from .cli import run

__all__ = []

if __name__ == "__main__":
    run()
