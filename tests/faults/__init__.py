"""Faults and hostile input (issue 35): signals, outputs onto inputs, injection, litter, the cache, full disks."""
