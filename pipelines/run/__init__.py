"""The run: an input MCAP read as events (`input_log`), the laser mount (`mount`), the run's options
(`options`), the runner that feeds the filter scan by scan (`runner`), and process start-up (`startup`)."""
