"""`dream batch`: many recordings calibrated, or one data set rendered, on a local process
pool or a Ray cluster (`batch.engine`)."""
