"""The blind real-vs-virtual rating study (thesis section 4.5.3) as an experiment kind: ``schedule`` (phases,
seeded order, redraws) and ``kind`` (its attempt, row and views)."""
