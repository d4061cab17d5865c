"""The fault decision: baselines, sequential tests, health holds, the joint check and each mode's decision state."""
