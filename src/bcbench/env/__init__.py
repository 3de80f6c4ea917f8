"""Push-T environment (exact gym-pusht wrapper) and the shared chunked controller."""
