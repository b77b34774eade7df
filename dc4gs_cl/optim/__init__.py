"""The optimiser, owned by the host: Adam's logic and learning rates (adam), and the Gaussians being trained, their
parameters and Adam's moments on the device kept aligned (trainable). Density control, which grows and shrinks
them, is densify/."""
