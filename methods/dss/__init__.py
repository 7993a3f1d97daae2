"""Deep Screen Space (Nalbach, Ritschel, Seidel, I3D 2014) as the `dss` method plugin."""
