"""Labelling keyframes in standard annotation tools: fan images and COCO JSON."""
