"""Layer 3, behaviour that needs no learning: the random-shooting MPC expert, scripted policies,
episode runners (local processes or Ray), expert evaluation, Minari datasets. Imports only the
layers below (envs, sim, util)."""
