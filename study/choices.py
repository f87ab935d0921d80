"""The subject-information choices of a session (section 4.5.3): light (no numpy), so ``study run --help``
lists them without loading the data layer."""

GENDERS = ("female", "male", "other", "unspecified")
HANDEDNESS = ("right", "left", "ambidextrous", "unspecified")
EXPERIENCE = ("none", "few", "regular")
