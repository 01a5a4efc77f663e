"""DS-Net network: point encoder, cylinder U-Net, heads, voxelizer and dynamic shifting."""
