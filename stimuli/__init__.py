"""Event-based contact transients: parametric pulses and decaying sinusoids, HFAM libraries, the sample catalog.

See docs/architecture.md ("stimuli") for the contract and docs/hfam_library.md for the library file.
The names are loaded on first use (PEP 562 ``__getattr__``), so ``python -m stimuli --help`` stays fast.
"""

from plumbing.lazy import lazy_exports

_EXPORTS = {"CatalogSample": "catalog", "load_catalog": "catalog", "HfamLibrary": "library",
            "DecayingSinusoid": "transients", "NoTransient": "transients", "Pulse": "transients",
            "Transient": "transients"}

__all__ = ["Pulse", "DecayingSinusoid", "NoTransient", "HfamLibrary", "Transient", "CatalogSample", "load_catalog"]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
