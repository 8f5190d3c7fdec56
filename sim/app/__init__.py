"""What a user runs and looks at: the `jiggle` command line and everything that only presents results.

`cli` builds the parser from one module per subcommand (`commands/`) and shared argument groups
(`args`); `loading` reads what several commands take; `report/` is `jiggle compare`'s report (metrics, skin
quality, plots, renders, report.html); `outputs/` what each other command writes; `view/` the browser viewer;
`batch` a library on Dask. Imports everything below; only the public API (jiggle/api.py) imports it."""
