"""Active + contrastive off-road segmentation (seed 001): InfoNCE, risk, frame selection, dense CRF."""
