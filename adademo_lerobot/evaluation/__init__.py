"""A policy's episodes: loading a checkpoint against a suite's features (`policy`) and running it on a batch of
initial states, with the success tables and files of an evaluation (`rollouts`)."""
