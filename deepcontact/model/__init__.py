"""Networks from grid images to impulse images, their losses, training and inference."""
