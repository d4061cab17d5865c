"""Offline identification and finding the modes: [A-SRIVC], [BCD-SRIVC], [UNS-SRIVC], the order scan, model checks."""
