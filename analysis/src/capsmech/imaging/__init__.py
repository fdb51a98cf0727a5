"""Images: from microscope frames to measurements (extraction), and frames rendered from simulations."""
