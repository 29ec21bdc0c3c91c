"""simn-sim: a MuJoCo closed-loop navigation testbed and the reference implementation of SIMN.

Importing the package registers the Gymnasium env ids (``SimnOffice-v0`` and variants).
"""

from simn_sim.env.gl import select_backend as _select_gl

_select_gl()

from simn_sim.env.registration import register_envs  # noqa: E402

register_envs()

__version__ = "0.1.0"
__all__ = ["__version__"]
