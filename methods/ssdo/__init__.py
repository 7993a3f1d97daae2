"""`ssdo`: Screen-Space Directional Occlusion's one-bounce indirect term (Ritschel, Grosch, Seidel 2009)."""
