"""moegs: Mixture-of-Experts dynamic Gaussian Splatting, reproducible.

Light imports only here; heavy modules (experts, routers) load on first use.
"""

from moegs.camera import Camera
from moegs.gaussians import GaussianFrame, cat

__all__ = ["Camera", "GaussianFrame", "cat"]
__version__ = "0.1.0"
