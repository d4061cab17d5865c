"""additive_rsrivc_ros: online tracking and fault diagnosis of mechanical resonances.

The numerics live in the ROS-free :mod:`additive_rsrivc_ros.core`; the ROS 2 node, the bag tools and
the command-line programs are thin shells around it.
"""

from . import numba_cache as _numba_cache
from ._version import __version__ as __version__

#: where this process caches compiled kernels (see :mod:`additive_rsrivc_ros.numba_cache`)
NUMBA_CACHE_DIR = _numba_cache.configure()
