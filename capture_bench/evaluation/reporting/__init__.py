"""Reporting an evaluation: records to estimates with 95% intervals, survival curves, paired
comparisons and the ranking (`metrics`, `aggregate`, `paired`), the report's sections and figures
(`summary`, `rliable_report`, `vision`, `pixel_comparison`, `watch`, `plots`), the report itself
(`report`), a report folder read back (`report_folder`), reports merged (`merge`) and a report
compared with the published one (`reproduction`)."""
