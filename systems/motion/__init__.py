"""The input and motion feature: releasing timed input events, and scripted motion along waypoints."""
