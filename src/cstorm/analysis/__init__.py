"""What a solved motion is worth: its success criteria (`criteria`), the fidelity of a
re-simulation (`fidelity`), the motor limits on every step (`torque`), the time step
against the integrator's stability limit (`timestep`), and the segments of a sequence
(`segments`)."""
