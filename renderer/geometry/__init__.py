"""Shapes, their intersection routines and the BVH over them."""
