"""``graphcal import-asterix``: ASTERIX recordings (and OpenSky ADS-B) to a dataset folder."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from graphcal.cli.common import (
    EXIT_BAD_INPUT,
    check_choice,
    check_output_folder,
    console,
    errors_to_exit,
    fail,
    print_wrapped,
    progress_bar,
)

#: Share of the input bytes left out of the data blocks above which the summary warns.
LOST_WARNING_SHARE = 0.01


def _format_span(span: tuple[float, float] | None) -> str:
    if span is None:
        return "-"
    first, last = span
    return f"{first:.1f} s .. {last:.1f} s ({last - first:.1f} s)"


def _parse_date(text: str | None) -> float | None:
    """``--date YYYY-MM-DD`` -> unix time [s] of that day's 00:00 UTC (exit 2 if not a date)."""
    if text is None:
        return None
    from datetime import UTC, datetime

    try:
        day = datetime.strptime(text, "%Y-%m-%d").replace(tzinfo=UTC)
    except ValueError:
        fail(f"--date {text}: not a date YYYY-MM-DD (the recording's UTC day)", EXIT_BAD_INPUT)
    return day.timestamp()


def _check_template_target(path: Path, overwrite: bool) -> None:
    """Refuse, before any decoding, a template path that cannot be written."""
    if path.is_dir():
        fail(f"--write-sites-template {path}: is a folder", EXIT_BAD_INPUT)
    if path.exists() and not overwrite:
        fail(f"--write-sites-template {path}: exists (give --overwrite to replace it)",
             EXIT_BAD_INPUT)
    if not path.parent.resolve().is_dir():
        fail(f"--write-sites-template {path}: the folder {path.parent} does not exist",
             EXIT_BAD_INPUT)
    if not overwrite:  # nor replaced if another process writes it meanwhile
        from graphcal.core.atomic import protect

        protect(path)


def _write_template(path: Path, decoded, user_sites, files: list[Path]) -> None:
    """``--write-sites-template``: the sites of every SAC/SIC, written atomically."""
    from graphcal.core.atomic import atomic_write_text
    from graphcal.io.asterix.decode import AsterixError
    from graphcal.io.asterix.tables import radar_inventory, sites_template

    if not decoded.count(48):
        raise AsterixError("no CAT048 target reports (plots) in the recording")
    inventory = radar_inventory(decoded, user_sites)
    atomic_write_text(path, sites_template(inventory, [p.name for p in files]))
    to_fill = sum(1 for r in inventory if r.cat034 is None)
    print_wrapped(
        f"wrote {path}: {len(inventory)} radars ({to_fill} without a CAT034 position to fill "
        "in); no dataset written. Fill in the positions, then run import-asterix again with "
        f"--sites {path}", out=console)


def import_asterix_command(
    files: Annotated[
        list[Path],
        typer.Argument(metavar="FILE...", help="ASTERIX recordings: raw blocks, pcap or pcapng."),
    ],
    out: Annotated[Path | None, typer.Option("--out", help="Dataset folder to write.")] = None,
    sites: Annotated[
        Path | None,
        typer.Option(help="sites.toml with radar positions; its radar tables may carry sac/sic "
                     "keys to name a radar (wins over CAT034 positions)."),
    ] = None,
    adsb: Annotated[
        Path | None,
        typer.Option(help="ADS-B source replacing the recording's CAT021 (see --adsb-format)."),
    ] = None,
    adsb_format: Annotated[
        str, typer.Option("--adsb-format", metavar="asterix|opensky",
                          help="Format of --adsb: asterix or opensky.")
    ] = "asterix",
    fmt: Annotated[str, typer.Option("--format", metavar="csv|parquet",
                                     help="Table format: csv or parquet.")] = "csv",
    date: Annotated[
        str | None,
        typer.Option(
            "--date", metavar="YYYY-MM-DD",
            help="The recording's UTC day: time_s is the ASTERIX time of day, counted from "
            "its 00:00 UTC, which the dataset records as epoch_utc. For a recording without "
            "capture times (raw .ast); with them (pcap) it must be their first day.",
        ),
    ] = None,
    overwrite: Annotated[
        bool, typer.Option(help="Replace an existing output folder (or sites template).")
    ] = False,
    sites_template: Annotated[
        Path | None,
        typer.Option(
            "--write-sites-template", metavar="FILE",
            help="Write a sites.toml with one radar table per SAC/SIC of the recording "
            "(id, sac, sic, plot counts, position keys to fill in) and stop: no dataset "
            "is written.",
        ),
    ] = None,
    cat021_edition: Annotated[
        str,
        typer.Option(
            "--cat021-edition", metavar="auto|0.23|0.26|2.x|...",
            help="CAT021 (ADS-B) edition of the recordings: auto (default) chooses per "
            "data block the edition (2.x, 0.26 or 0.23) under which the block parses "
            "with plausible content; an edition (0.23, 0.24, 0.25, 0.26, 2.x, or 2.1 ... "
            "2.7) forces it for every CAT021 block.",
        ),
    ] = "auto",
) -> None:
    """Decode ASTERIX CAT048/CAT021/CAT034 recordings into a dataset folder."""
    from rich.table import Table

    from graphcal.io.asterix.decode import (
        ASTERIX_CATEGORIES,
        CAT021_EDITION_CHOICES,
        decode_files,
    )
    from graphcal.io.asterix.tables import (
        build_tables,
        load_user_sites,
        recording_epoch,
        sorted_by_time,
        time_span,
    )
    from graphcal.io.folder import write_dataset
    from graphcal.io.opensky import read_opensky_adsb

    if fmt not in ("csv", "parquet"):
        fail(f"--format must be csv or parquet, not '{fmt}'", EXIT_BAD_INPUT)
    if adsb_format not in ("asterix", "opensky"):
        fail(f"--adsb-format must be asterix or opensky, not '{adsb_format}'", EXIT_BAD_INPUT)
    check_choice(cat021_edition, "--cat021-edition", CAT021_EDITION_CHOICES, "CAT021 edition")
    if not files:
        fail("give at least one recording FILE", EXIT_BAD_INPUT)
    if out is None and sites_template is None:
        fail("give --out DIR (the dataset to write) or --write-sites-template FILE",
             EXIT_BAD_INPUT)
    if sites_template is not None:
        _check_template_target(sites_template, overwrite)
    given_epoch = _parse_date(date)
    for path in [*files, *([adsb] if adsb is not None else [])]:
        if not path.is_file():
            fail(f"{path}: no such file", EXIT_BAD_INPUT)
    check_output_folder(out, "--out", overwrite=overwrite, inputs=[*files, adsb, sites])
    with errors_to_exit():
        user_sites = None if sites is None else load_user_sites(sites)
        with progress_bar("decoding ASTERIX") as callback:
            decoded = decode_files(files, progress=callback, cat021_edition=cat021_edition)
        adsb_table = None
        epoch = recording_epoch(decoded)
        if given_epoch is not None:
            if epoch is not None and epoch != given_epoch:
                from graphcal.io.asterix.tables import TimeBase

                fail(f"--date {date}: the recording's capture times begin on "
                     f"{TimeBase(epoch).date} UTC; give that day or leave --date out",
                     EXIT_BAD_INPUT)
            epoch = given_epoch
        if adsb is not None:
            if adsb_format == "opensky":
                adsb_table = read_opensky_adsb(adsb, epoch_unix_s=epoch)
                epoch = adsb_table.attrs["epoch_unix_s"] if epoch is None else epoch
            else:
                with progress_bar("decoding ADS-B") as callback:
                    extra = decode_files([adsb], progress=callback,
                                         cat021_edition=cat021_edition)
                decoded.extend(extra)
        source = files[0] if len(files) == 1 else None
        if sites_template is not None:
            _write_template(sites_template, decoded, user_sites, files)
            return
        assert out is not None
        tables = build_tables(decoded, user_sites=user_sites, adsb=adsb_table,
                              epoch_unix_s=epoch, source=source)
        dataset = tables.dataset
        dataset.plots = sorted_by_time(dataset.plots, ["radar_id", "time_s"])
        if dataset.adsb is not None:
            dataset.adsb = sorted_by_time(dataset.adsb, ["time_s", "target_id"])
        write_dataset(dataset, out, fmt=fmt, overwrite=overwrite)

    stats, decode = tables.stats, decoded.stats
    table = Table()
    for name in ("radar", "SAC", "SIC", "position from", "plots"):
        table.add_column(name, justify="left" if name in ("radar", "position from") else "right")
    for radar_id, n_plots in stats.plots_by_radar.items():
        sac, sic = stats.sources[radar_id]
        table.add_row(radar_id, str(sac), str(sic), stats.site_origin[radar_id], str(n_plots))
    print_wrapped(str(out), label="wrote", out=console)  # above the table, a long path whole
    console.print(table)
    day = tables.time_base.date
    lines = [
        f"time base: seconds since 00:00 UTC of "
        f"{day or 'the first report day (date unknown: give it with --date)'}"
        f"; span {_format_span(time_span([dataset.plots, dataset.adsb]))}",
        f"ADS-B: {stats.adsb_reports} reports of {stats.aircraft} aircraft"
        + (f" (from {adsb}, {adsb_format})" if adsb is not None else ""),
        f"blocks: {decode.blocks} read, {decode.blocks_decoded} decoded; records: "
        + (", ".join(f"CAT{c:03d} {n}" for c, n in sorted(decode.records.items())) or "none"),
    ]
    editions_021 = sorted((edition, n) for (category, edition), n in decode.editions.items()
                          if category == 21)
    if editions_021:
        lines.append("CAT021 editions: " + ", ".join(
            f"{edition} ({n} block{'s' if n != 1 else ''})" for edition, n in editions_021)
            + ("" if cat021_edition == "auto" else " (forced)"))
    defined = {c: n for c, n in decode.skipped_categories.items() if c in ASTERIX_CATEGORIES}
    undefined = {c: n for c, n in decode.skipped_categories.items() if c not in defined}
    if defined:
        lines.append("skipped categories: " + ", ".join(
            f"CAT{c:03d} ({n} blocks)" for c, n in sorted(defined.items())))
    if undefined:
        lines.append("skipped blocks of categories ASTERIX does not define (corrupted CAT "
                     "bytes?): " + ", ".join(f"CAT{c:03d} ({n} blocks)"
                                            for c, n in sorted(undefined.items())))
    lost = decode.bytes_unsplit
    if lost:
        share = 100.0 * lost / max(decode.bytes_read, 1)
        what = (files[0].name if len(files) == 1 and adsb is None
                else "the input" if adsb is None else "the inputs")
        lines.append(f"{lost:,} bytes ({share:.2g} %) of {what} could not be split into "
                     "blocks and were skipped" if share < 0.1 else
                     f"{lost:,} bytes ({share:.1f} %) of {what} could not be split into "
                     "blocks and were skipped")
    if decode.rejected:
        lines.append("rejected: " + ", ".join(
            f"{reason} {n}" for reason, n in sorted(decode.rejected.items())))
    if stats.skipped:
        lines.append("reports skipped: " + ", ".join(
            f"{reason} {n}" for reason, n in sorted(stats.skipped.items())))
    if stats.adsb_without_height:
        lines.append(
            f"ADS-B without geometric height (I021/140): {stats.adsb_without_height} reports "
            f"({stats.adsb_without_height_baro} with a flight level, I021/145, as baro_alt_m) "
            "kept with alt_m empty: their positions can be inspected, but a calibration "
            "cannot use them without a geometric height")
    if adsb_table is not None:
        dropped = ", ".join(f"{k} {v}" for k, v in adsb_table.attrs["dropped"].items() if v)
        lines.append(f"OpenSky rows: {adsb_table.attrs['rows_read']} read; dropped: "
                     f"{dropped or 'none'}; height from {adsb_table.attrs['height_source']}")
    plot_span = time_span([dataset.plots])
    adsb_span = time_span([dataset.adsb])
    if plot_span and adsb_span and (adsb_span[1] < plot_span[0] or adsb_span[0] > plot_span[1]):
        lines.append("warning: the ADS-B reports do not overlap the plots in time "
                     "(different days or recordings?)")
    for line in lines:
        print_wrapped(line, out=console)
    if decode.bytes_read and decode.bytes_unsplit > LOST_WARNING_SHARE * decode.bytes_read:
        print_wrapped(
            f"{100.0 * decode.bytes_unsplit / decode.bytes_read:.1f} % of the ASTERIX bytes "
            "could not be split into data blocks (corrupted lengths or not ASTERIX data): "
            "the dataset lacks the reports they held", label="warning:", style="bold red",
            out=console)
