"""Denoisers for rendered frames: Intel Open Image Denoise for still images (an optional extra) and the WRLS
temporal denoiser of Iglesias-Guitian et al. (``../shared/papers/vpt_realtime_denoising_wrls.txt``) for frame
sequences (progressive renders, orbits, the viewer). Each works on any renderer's (H, W, 3) float32 layers;
``registry`` lists the ones ``pfn-render --denoise`` offers."""
