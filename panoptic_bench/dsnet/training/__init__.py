"""DS-Net training: losses, per-stage loss steps and the resumable training loop."""
