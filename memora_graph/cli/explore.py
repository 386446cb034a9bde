"""`memora explore`: write one participant's memory as a self-contained HTML page."""

from __future__ import annotations

import click


@click.command("explore")
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.option("--participant", required=True, help="Whose memory to show (P01).")
@click.option("--out", type=click.Path(dir_okay=False), help="The HTML file to write (default: P01.html).")
def explore_cmd(bank, participant, out):
    """Write an explorer page for one participant's memory: one HTML file, nothing fetched when opened.

    It shows a timeline of the videos in 10 s segments coloured by place, swimlanes of each
    object's state over a video with the editor's decisions (ADD / UPDATE / DELETE / NOOP),
    the routines and preferences with their supporting segments, and a graph of routines,
    objects and places. Filter by object and by place; the view is kept in the URL
    (memory.html#object=P01:plate&place=sink_area), so it can be bookmarked.

    \b
    Examples:
      memora explore banks/epic --participant P01 --out memory.html
      xdg-open memory.html                  # or open it in any browser, offline
    """
    from memora_graph.explore import write_explorer
    from memora_graph.text import counted

    path, data = write_explorer(bank, participant, out or f"{participant}.html")
    size = path.stat().st_size / 1e6
    counts = ", ".join(counted(len(data[k]), noun) for k, noun in (("videos", "video"), ("segments", "segment"),
                       ("events", "state event"), ("routines", "routine"), ("preferences", "preference")))
    click.echo(f"{participant}: {counts} -> {path} ({size:.1f} MB)")
