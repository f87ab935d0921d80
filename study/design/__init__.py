"""Counterbalancing condition order across participants: Latin squares and Williams designs, assigned from the
participant list (``python -m study design``; the kinds read a subject's order from the table it writes)."""
