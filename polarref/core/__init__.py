"""Core services every stage uses: geometry and angles, landmarks, errors, atomic files, strict
records, provenance, progress, where tasks run (execution), heap settings, reference-data paths."""
