"""dc4gs-cl: a vendor-portable 3D Gaussian Splatting trainer with DC4GS density control, on OpenCL."""
__version__ = "0.1.0"
