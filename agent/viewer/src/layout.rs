//! The layout a reviewer opens on, declared once as a table of panels: [`blueprint`] builds
//! rerun's blueprint from it, and the read-back test holds each panel of a recording to it
//! (every panel has data on the timeline the view opens on).

/// What kind of job the view shows: it decides the timeline the view opens on and the panels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Job {
    /// The agent beside a printer: stations scan after layers, so everything is placed on the
    /// `layer` timeline (the scan layer: the last layer printed when the station scanned) and
    /// the view opens on it.
    Printing {
        /// Whether the agent advises corrections, whose history the view shows.
        corrections: bool,
    },
    /// `asbuilt inspect` of scan files of a finished part: the `station` timeline.
    Survey {
        /// Whether the job has layer bands (a layer height), whose means the view shows.
        layer_bands: bool,
    },
}

impl Job {
    /// The timeline the view opens on.
    pub fn timeline(self) -> &'static str {
        match self {
            Job::Printing { .. } => "layer",
            Job::Survey { .. } => "station",
        }
    }
}

/// The tab a panel is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tab {
    /// The part large, the current station and the scan layer's findings beside it.
    Part,
    /// Each layer band across scan layers (a print), or its means (a survey).
    Layers,
}

/// What a panel draws, and the archetype its entities must hold for it to draw anything.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PanelKind {
    /// Meshes, points, boxes: anything spatial.
    Spatial3D,
    /// A bar chart, the latest at the time cursor.
    BarChart,
    /// Series against the timeline: they need data on it, never static.
    TimeSeries,
    /// Markdown, the latest at the time cursor.
    Text,
}

impl PanelKind {
    /// The component that must be logged for the panel to draw (`None`: any spatial one).
    pub fn component(self) -> Option<&'static str> {
        match self {
            PanelKind::Spatial3D => None,
            PanelKind::BarChart => Some("BarChart:values"),
            PanelKind::TimeSeries => Some("Scalars:scalars"),
            PanelKind::Text => Some("TextDocument:text"),
        }
    }
}

/// One panel of the layout.
#[derive(Debug, Clone, Copy)]
pub struct Panel {
    /// The tab it is on.
    pub tab: Tab,
    /// What it draws.
    pub kind: PanelKind,
    /// Its title.
    pub title: &'static str,
    /// Its origin; unless `contents` says otherwise it shows the origin and all below.
    pub origin: &'static str,
    /// rerun's entity queries (`+ /a/**`, `- /b`), when not the origin's subtree.
    pub contents: &'static [&'static str],
    /// Its share of the column (part tab) or of the tab's height (layers tab).
    pub share: f32,
    /// The jobs it is part of.
    pub shown: fn(Job) -> bool,
}

fn always(_: Job) -> bool {
    true
}

fn printing(j: Job) -> bool {
    matches!(j, Job::Printing { .. })
}

fn advising(j: Job) -> bool {
    j == Job::Printing { corrections: true }
}

fn surveyed_bands(j: Job) -> bool {
    j == Job::Survey { layer_bands: true }
}

/// Every panel, in the order it is laid out: the part tab's 3D view first (it takes the left
/// three quarters), its column, then the layers tab top to bottom.
pub const PANELS: &[Panel] = &[
    Panel {
        tab: Tab::Part,
        kind: PanelKind::Spatial3D,
        title: "part",
        origin: "/",
        contents: &[
            "+ /design",
            "+ /stations/**",
            "+ /deviations/**",
            "+ /profiler/**",
            "+ /findings/areas/**",
            "+ /findings/markers",
            "+ /findings/ruler",
            "+ /missing",
            "+ /m3c2",
            "- /stations/*/histogram",
        ],
        share: 3.0,
        shown: always,
    },
    Panel::of(
        Tab::Part,
        PanelKind::BarChart,
        "current station: deviation histogram",
    )
    .at("/histogram", 1.0, always),
    Panel::of(
        Tab::Part,
        PanelKind::TimeSeries,
        "station statistics (mm): a dot per station",
    )
    .at("/stats", 1.0, always),
    Panel::of(
        Tab::Part,
        PanelKind::Text,
        "findings of the scan layer at the cursor (numbers as in the report)",
    )
    .at("/findings/table", 1.4, always),
    Panel::of(Tab::Part, PanelKind::Text, "colours").at("/legend", 0.6, always),
    Panel::of(
        Tab::Layers,
        PanelKind::TimeSeries,
        "width per layer band (mm), by scan layer (each once all its stations are in)",
    )
    .at("/history/width_mm", 1.0, printing),
    Panel::of(
        Tab::Layers,
        PanelKind::TimeSeries,
        "relative width per layer band (mm): less the scan layer's median; a rising line is creep",
    )
    .at("/history/relative_width_mm", 1.0, printing),
    Panel::of(
        Tab::Layers,
        PanelKind::TimeSeries,
        "shift per layer band (mm), by scan layer",
    )
    .at("/history/shift_mm", 1.0, printing),
    Panel::of(
        Tab::Layers,
        PanelKind::TimeSeries,
        "top height deviation (mm), by scan layer",
    )
    .at("/history/top_mm", 1.0, printing),
    Panel::of(
        Tab::Layers,
        PanelKind::TimeSeries,
        "corrections advised, by scan layer: z per layer (mm), flow − 1 (%), path (mm)",
    )
    .at("/history/corrections", 1.0, advising),
    Panel::of(
        Tab::Layers,
        PanelKind::BarChart,
        "mean M3C2 deviation per layer band (mm), of the scan layer at the cursor",
    )
    .at("/layers/m3c2_mean_mm", 1.0, printing),
    Panel::of(
        Tab::Layers,
        PanelKind::BarChart,
        "mean C2M distance per layer band (mm)",
    )
    .at("/layers/c2m_mean_mm", 1.0, surveyed_bands),
    Panel::of(Tab::Layers, PanelKind::Text, "each layer band's means").at(
        "/layers/table",
        1.5,
        surveyed_bands,
    ),
];

impl Panel {
    /// A panel titled `title`, showing its origin's subtree; [`Panel::at`] places it.
    const fn of(tab: Tab, kind: PanelKind, title: &'static str) -> Self {
        Self {
            tab,
            kind,
            title,
            origin: "/",
            contents: &[],
            share: 1.0,
            shown: always,
        }
    }

    /// The panel at `origin`, with its `share` of the space, in the jobs `shown` says.
    const fn at(self, origin: &'static str, share: f32, shown: fn(Job) -> bool) -> Self {
        Self {
            origin,
            share,
            shown,
            ..self
        }
    }

    /// Whether the panel shows the entity at `path` (`/a/b`), by its queries: the last query
    /// that matches decides, as in rerun.
    pub fn includes(&self, path: &str) -> bool {
        let own = [format!("+ {}/**", self.origin.trim_end_matches('/'))];
        let queries: Vec<&str> = if self.contents.is_empty() {
            own.iter().map(String::as_str).collect()
        } else {
            self.contents.to_vec()
        };
        let mut shown = false;
        for q in queries {
            let (include, pattern) = match q.split_once(' ') {
                Some(("+", p)) => (true, p),
                Some(("-", p)) => (false, p),
                _ => continue,
            };
            if matches(pattern, path) {
                shown = include;
            }
        }
        shown
    }
}

/// rerun's entity path patterns as the table uses them: parts that are names or `*` (one
/// part), and a trailing `/**` (the path and everything below it).
fn matches(pattern: &str, path: &str) -> bool {
    let parts = |s: &str| -> Vec<String> {
        s.split('/')
            .filter(|p| !p.is_empty())
            .map(str::to_string)
            .collect()
    };
    let (mut pat, path) = (parts(pattern), parts(path));
    let subtree = pat.last().is_some_and(|p| p == "**");
    if subtree {
        pat.pop();
    }
    let fits = |n: usize| pat.iter().zip(&path[..n]).all(|(a, b)| a == "*" || a == b);
    if subtree {
        path.len() >= pat.len() && fits(pat.len())
    } else {
        path.len() == pat.len() && fits(pat.len())
    }
}

/// The panels of `job`'s view.
pub fn panels(job: Job) -> impl Iterator<Item = &'static Panel> {
    PANELS.iter().filter(move |p| (p.shown)(job))
}

/// What a reviewer sees first: the part (design, stations, coloured points, the scan layer's
/// findings as numbered markers) large, beside the current station's histogram, the stations'
/// statistics and the findings as text; a second tab with the layer bands. The view opens on
/// `job`'s timeline, following the latest data.
pub fn blueprint(job: Job) -> rerun::blueprint::Blueprint {
    use rerun::blueprint::{
        BarChartView, Blueprint, BlueprintPanel, ContainerLike, Horizontal, SelectionPanel,
        Spatial3DView, Tabs, TextDocumentView, TimePanel, TimeSeriesView, Vertical,
    };
    let view = |p: &Panel| -> ContainerLike {
        let contents = p.contents.iter().copied();
        match p.kind {
            PanelKind::Spatial3D => Spatial3DView::new(p.title)
                .with_origin(p.origin)
                .with_contents(contents)
                .into(),
            PanelKind::BarChart => BarChartView::new(p.title).with_origin(p.origin).into(),
            PanelKind::TimeSeries => TimeSeriesView::new(p.title).with_origin(p.origin).into(),
            PanelKind::Text => TextDocumentView::new(p.title).with_origin(p.origin).into(),
        }
    };
    let on = |tab: Tab| panels(job).filter(move |p| p.tab == tab);
    let (big, column): (Vec<&Panel>, Vec<&Panel>) =
        on(Tab::Part).partition(|p| p.kind == PanelKind::Spatial3D);
    let column_view = Vertical::new(column.iter().map(|p| view(p)))
        .with_row_shares(column.iter().map(|p| p.share).collect::<Vec<_>>());
    let mut part_views: Vec<ContainerLike> = big.iter().map(|p| view(p)).collect();
    let mut shares: Vec<f32> = big.iter().map(|p| p.share).collect();
    part_views.push(column_view.into());
    shares.push(1.0);
    let part = Horizontal::new(part_views)
        .with_name("part")
        .with_column_shares(shares);
    let layers: Vec<&Panel> = on(Tab::Layers).collect();
    let layers_name = match job {
        Job::Printing { .. } => "layer history",
        Job::Survey { .. } => "layer bands",
    };
    let mut tabs: Vec<ContainerLike> = vec![part.into()];
    if !layers.is_empty() {
        tabs.push(
            Vertical::new(layers.iter().map(|p| view(p)))
                .with_row_shares(layers.iter().map(|p| p.share).collect::<Vec<_>>())
                .with_name(layers_name)
                .into(),
        );
    }
    // The side panels start folded away and the time panel to its play bar (the timeline,
    // its cursor and the scan layer): the part gets the window.
    let folded = rerun::blueprint::components::PanelState::Collapsed;
    Blueprint::new(Tabs::new(tabs))
        .with_blueprint_panel(BlueprintPanel::new().with_state(folded))
        .with_selection_panel(SelectionPanel::new().with_state(folded))
        .with_time_panel(
            TimePanel::new()
                .with_state(folded)
                .with_timeline(job.timeline())
                .with_play_state(rerun::blueprint::components::PlayState::Following),
        )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_panel_shows_its_origin_and_below_or_what_its_queries_say() {
        let part = &PANELS[0];
        assert!(part.includes("/design"));
        assert!(part.includes("/stations/job1/station3"));
        assert!(!part.includes("/stations/job1/histogram"));
        assert!(part.includes("/findings/markers"));
        assert!(!part.includes("/findings/table"));
        assert!(!part.includes("/stats/mean_mm"));
        let width = panels(Job::Printing { corrections: false })
            .find(|p| p.origin == "/history/width_mm")
            .unwrap();
        assert!(width.includes("/history/width_mm/band_003"));
        assert!(width.includes("/history/width_mm"));
        assert!(!width.includes("/history/width"));
        assert!(!width.includes("/history/shift_mm/band_003"));
    }

    #[test]
    fn each_job_has_its_panels() {
        let titles = |j| panels(j).map(|p| p.title).collect::<Vec<_>>();
        assert_eq!(titles(Job::Printing { corrections: true }).len(), 11);
        assert_eq!(titles(Job::Printing { corrections: false }).len(), 10);
        assert_eq!(titles(Job::Survey { layer_bands: false }).len(), 5);
        assert_eq!(titles(Job::Survey { layer_bands: true }).len(), 7);
    }
}
