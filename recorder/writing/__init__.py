"""What a rig produces (typed stream items) and the MCAP writer that records it."""
