"""What every report page uses: the HTML builder, the one number formatter, figure helpers, tables,
the run's artifacts as the pages read them."""
