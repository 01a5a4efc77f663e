"""DS-Net data: datasets of labelled scans, class maps and training augmentation."""
