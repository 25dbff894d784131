"""The MCAP layer shared by `ingest` and `pipelines`: channel names, schemas and message builders
(`mcaplog.channels`), and the atomic writer and decoding reader (`mcaplog.mcapio`).

It sits below both packages so that neither imports the other for its file format, and beside the
pure filter core `gslam`, which knows nothing of files.
"""
