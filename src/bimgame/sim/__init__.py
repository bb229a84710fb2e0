"""Layer 1, the puzzle itself: maze geometry and geodesic distance, MuJoCo physics, the top-down
raster, the task rules and time limits. Imports only :mod:`bimgame.util`."""
