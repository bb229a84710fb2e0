"""Layer 0, used by every other layer and importing none of them: atomic files and locks, settings
checks, progress bars, signal handling, image files, seeds derived from a run seed."""
