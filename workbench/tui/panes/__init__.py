"""One pane per stage of the design: plant, MPC, synthesis, verification, session."""
