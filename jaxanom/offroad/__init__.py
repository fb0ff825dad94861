"""Active + contrastive off-road segmentation (docs/papers/offroad.md): InfoNCE, risk, frame selection, dense CRF."""
