"""Analyses: what a sweep's results database, its trials run again, or ``taskcam run``'s
run directories say about a result, read from them."""
