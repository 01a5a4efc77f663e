"""Parity with the official DS-Net code: key tables and import of its released checkpoints."""
