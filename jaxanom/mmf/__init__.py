"""Multi-Mechanism Fusion (MMF, docs/papers/mmf.md): the paper's maps, synthesis and post-processor.

Modules: ``uncertainty`` (Eqs. 1-2 normalised, road probability), ``perceptual`` (Eqs. 3-4),
``synthesis`` (class-mean and SPADE resynthesis), ``gan`` / ``gan_train`` (the SPADE
generator's losses and GAN training), ``postprocess`` (Eq. 6 superpixel scores),
``training_free`` (Eqs. 1-2, SLIC and Eq. 6 on any network's logits and real frames).
"""
