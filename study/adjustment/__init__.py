"""The method of adjustment: the participant adjusts a comparison until it matches a reference (``kind =
"adjustment"``)."""
