"""Time: the clock interface and its wall and mock implementations, the bus clock (simulated time), the lockstep protocol, and the in-process composition that runs a graph on one timeline."""
