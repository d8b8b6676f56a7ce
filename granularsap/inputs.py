"""Input coercion with granularsap's error messages, for code built on granularsap.

Every public function of granularsap validates its arguments with these
helpers before any compiled call; adapters (lammps_bridge, readers, your own
wrappers) use them too, so a bad argument gets the same message everywhere:
it names the argument, what was expected, what was received.

>>> from granularsap.inputs import as_coords
>>> as_coords([[0, 1, 2]], "positions").dtype
dtype('float64')
"""

from ._validate import as_coords, as_scalar, as_vector, check_n_threads
from .search import as_labels, as_radii

__all__ = ["as_coords", "as_labels", "as_radii", "as_scalar", "as_vector", "check_n_threads"]
