"""Analysis of recordings: summary and plot (summary), mantle profiles and animation (profiles)."""

from pulsejet_sim.analysis.summary import (
    format_summary,
    main_plot,
    main_summary,
    plot,
    plot_figure,
    SNAPSHOT_AXES_LABEL,
    summarize,
)

__all__ = [
    'format_summary', 'main_plot', 'main_summary', 'plot', 'plot_figure', 'SNAPSHOT_AXES_LABEL',
    'summarize',
]
