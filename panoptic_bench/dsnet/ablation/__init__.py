"""DS-Net ablations (paper Tables 4/5, Figs. 4-7) on cached backbone outputs."""
