"""The summary of a contacts HDF5 file: counts per frame, coordination, births and deaths.

:func:`summarize` reads what ``granularsap info`` prints (as a dict, arrays per
frame included); :func:`plot` draws contacts and the mean coordination number
per frame.
"""

from __future__ import annotations

import os

__all__ = ["plot", "summarize"]


def summarize(path) -> dict:
    """The summary ``granularsap info`` prints, as a dict (arrays per frame included).

    Raises
    ------
    ValueError
        Naming the file, when HDF5 cannot read what the summary needs (a file
        damaged after it was written: a flipped byte in a header or a chunk).
    """
    try:
        return _summarize(path)
    except (KeyError, RuntimeError, OSError) as exc:
        if isinstance(exc, (FileNotFoundError, PermissionError, IsADirectoryError)):
            raise
        raise ValueError(f"{os.fspath(path)}: damaged contacts file, HDF5 cannot read it: "
                         f"{exc}") from exc


def _summarize(path):
    import numpy as np

    from .hdf5 import ContactsFile

    with ContactsFile(path, allow_incomplete=True) as cf:
        n_part = cf.n_particles
        n_con = cf.n_contacts
        coord = np.divide(2.0 * n_con, n_part, out=np.zeros(len(n_con)), where=n_part > 0)
        return {
            "path": cf.path,
            "complete": cf.complete,
            "schema_version": cf.schema_version,
            "granularsap_version": cf.granularsap_version,
            "parameters": cf.parameters,
            "frames": cf.n_frames,
            "steps": cf.step.tolist(),
            "n_particles": n_part.tolist(),
            "particles_changed": int(np.count_nonzero(np.diff(n_part))),
            "empty_frames": int(np.count_nonzero(n_part == 0)),
            "n_contacts": n_con.tolist(),
            "coordination": coord.tolist(),
            "n_born": cf.n_born.tolist(),
            "n_died": cf.n_died.tolist(),
            "timing": cf.timing,
        }


def plot(summary, png):
    """Write a PNG of contacts and mean coordination number per frame (or timestep)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    steps = np.asarray(summary["steps"])
    x = steps if len(steps) and np.all(steps >= 0) else np.arange(summary["frames"])
    xlabel = "timestep" if x is steps else "frame"
    fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(6, 5))
    ax1.plot(x, summary["n_contacts"], marker=".")
    ax1.set_ylabel("contacts")
    ax2.plot(x, summary["coordination"], marker=".", color="C1")
    ax2.set_ylabel("mean coordination number")
    ax2.set_xlabel(xlabel)
    fig.suptitle(os.path.basename(summary["path"]))
    fig.tight_layout()
    fig.savefig(png, dpi=100)
    plt.close(fig)
