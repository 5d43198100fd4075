"""Pictures of what is simulated: steps as PNG/SVG, runs as GIF/MP4/WebM or a one-file HTML
viewer, grid samples as panels (`dc render`)."""
