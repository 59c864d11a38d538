"""Double Merge and Halting Car: synthetic multi-agent driving scenarios on carlo_lite."""
