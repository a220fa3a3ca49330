"""MapTRv2-style vectorized local map: GT vectors, fixed-point targets, dataset, info export."""
