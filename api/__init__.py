"""HTTP API (FastAPI): upload stereo pairs, poll jobs, download disparity maps."""
