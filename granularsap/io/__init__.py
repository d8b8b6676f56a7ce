"""Trajectory readers and the HDF5 contacts format (no physics here).

:func:`iter_frames` reads LAMMPS text dumps (own reader) and anything ASE or
MDAnalysis reads; :func:`compute_contacts` runs the engine over every frame
and writes one HDF5 file (schema in README.md and
:mod:`granularsap.io.hdf5`); :func:`read_contacts` reads it back.
"""

from ._frame import Frame, box_to_cell, cell_to_box
from .hdf5 import (
    SCHEMA_VERSION,
    ContactsFile,
    ContactsWriter,
    IncompleteFileError,
    read_contacts,
)
from .lammps_dump import DumpFormatError, iter_lammps_dump
from .pipeline import ContactParams, FrameError, compute_contacts, frame_contacts
from .readers import TrajectoryError, count_frames, iter_frames

__all__ = [
    "SCHEMA_VERSION",
    "ContactParams",
    "ContactsFile",
    "ContactsWriter",
    "DumpFormatError",
    "Frame",
    "FrameError",
    "IncompleteFileError",
    "TrajectoryError",
    "box_to_cell",
    "cell_to_box",
    "compute_contacts",
    "count_frames",
    "frame_contacts",
    "iter_frames",
    "iter_lammps_dump",
    "read_contacts",
]
