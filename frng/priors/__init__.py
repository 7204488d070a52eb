"""The two frozen priors F-RNG builds on: an LRM backbone and an intrinsic decomposition model (IDM).

Registries map config names to implementations so a user can plug in a bigger backbone or another IDM
without touching F-RNG (``backbone.kind`` / ``idm.kind`` in the config).
"""
