"""X-JEPA model family (paper §3, App. B): encoders, causal AdaLN predictor, direct Δ heads, variants."""

from .xjepa import (
    OBJECTIVES,
    SYSID_PARAMS,
    VARIANTS,
    XJEPA,
    area_downsample,
    check_variant,
)

__all__ = ["XJEPA", "VARIANTS", "OBJECTIVES", "SYSID_PARAMS", "area_downsample", "check_variant"]
