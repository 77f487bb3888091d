"""Control: velocity control (ROV), DP control (surface vessels), operator modes, command gate."""
