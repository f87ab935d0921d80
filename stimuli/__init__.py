"""Event-based contact transients: parametric pulses and decaying sinusoids, HFAM libraries, the sample catalog.

See docs/architecture.md ("stimuli") for the contract and docs/hfam_library.md for the library file.
"""

from .catalog import CatalogSample, load_catalog
from .library import HfamLibrary
from .transients import DecayingSinusoid, NoTransient, Pulse, Transient

__all__ = ["Pulse", "DecayingSinusoid", "NoTransient", "HfamLibrary", "Transient", "CatalogSample", "load_catalog"]
