"""Studies: one part of the pipeline measured over a grid of conditions or many
generated scenes, against the simulator's truth."""
