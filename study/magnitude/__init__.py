"""Magnitude estimation: the participant gives each stimulus a number, with or without a modulus (``kind =
"magnitude"``)."""
