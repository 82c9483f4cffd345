"""Chapter 4: strength surfaces of every model variant and the claims of Sec. 4.3-4.4
===================================================================================

- :mod:`.surfaces`  max force and activations per direction as the deep extensors are weakened
- :mod:`.claims`    the qualitative claims, each evaluated with both outcomes possible
- :mod:`.plots`     per-muscle radars and activation-share bars (imported on its own: it loads matplotlib)
"""

from neckstrength.surfaces.claims import evaluate_claims
from neckstrength.surfaces.surfaces import Surface, activation_slopes, deep_extensor_mask, strength_surface

__all__ = ["evaluate_claims", "Surface", "activation_slopes", "deep_extensor_mask", "strength_surface"]
