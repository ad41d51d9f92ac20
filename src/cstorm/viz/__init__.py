"""Pictures of models and motions: planar drawings, plots, animations (matplotlib)."""
