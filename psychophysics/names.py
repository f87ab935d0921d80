"""The names of the psychometric functions and of the adaptive methods, defined once.

Light (the standard library only): the commands' parsers list them in ``--help`` without loading numpy or
scipy (``analysis psychometric --function``, ``study simulate-observer --method``, a protocol's
``[experiment] method``).
"""

#: the sigmoids of the psychometric function (:mod:`psychophysics.psychometric`)
FUNCTIONS = ("logistic", "normal", "weibull")
#: the adaptive methods by the name protocol files, states and ``--method`` use (:mod:`psychophysics.methods`)
METHOD_NAMES = ("updown", "weighted", "quest+", "psi")
