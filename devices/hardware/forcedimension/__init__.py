"""Force Dimension devices (omega, sigma, delta, and the Falcon through their SDK) via ``forcedimension-core``."""
