"""Many flights: sweep and tune over a spec, each run flown offline or through the graph, into an output directory held
by one writer."""
