"""nsim: a handheld video of a real room in, a photorealistic dynamic robot simulator out."""

__version__ = "0.1.0"
