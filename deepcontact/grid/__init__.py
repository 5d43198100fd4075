"""Steps as grid images: SPH splatting of bodies and contacts, and bilinear interpolation back."""
