"""Leaves: shared types (`episodes`) and helpers every layer may import; they import none of the layers."""
