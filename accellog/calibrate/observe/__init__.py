"""Holds -> windows -> observation tables: segmentation (whole or chunk by chunk), static detection, label checks, the noise of a hold."""
