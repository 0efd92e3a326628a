//! What a report read back from a recording lacks against what the live agent reported: the
//! demo's check that its recording holds every point of every station.

use asbuilt_protocol::StationReport;

use crate::Report;

impl Report {
    /// The stations whose points this report lacks, against each station's latest report from
    /// the live agent: (name, points recorded, points reported).
    pub fn short_of_live(&self, live: &[StationReport]) -> Vec<(String, u64, u64)> {
        let recorded: Vec<(&str, Option<u8>, u64)> = self
            .stations
            .iter()
            .map(|s| (s.id.as_str(), s.attempt, s.points))
            .collect();
        short_of(&recorded, live)
    }
}

/// [`Report::short_of_live`] over each recorded section's (station name, attempt from the
/// second on, points).
fn short_of(
    recorded: &[(&str, Option<u8>, u64)],
    live: &[StationReport],
) -> Vec<(String, u64, u64)> {
    live.iter()
        .filter_map(|r| {
            let name = r.name.as_str();
            let attempt = (r.attempt > 1).then_some(r.attempt);
            let points = recorded
                .iter()
                .filter(|(id, a, _)| *id == name && *a == attempt)
                .map(|(_, _, p)| *p)
                .max()
                .unwrap_or(0);
            (points < r.points_received).then(|| (name.to_string(), points, r.points_received))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use asbuilt_protocol::FixedText;

    fn reported(name: &str, attempt: u8, points: u64) -> StationReport {
        let mut r = StationReport::new(1, 0);
        r.name = FixedText::new(name).unwrap();
        r.attempt = attempt;
        r.points_received = points;
        r
    }

    #[test]
    fn a_station_is_short_when_its_recorded_attempt_has_fewer_points_or_none() {
        let live = [
            reported("L008-S1", 1, 100),
            reported("L008-S2", 2, 200),
            reported("L008-S3", 1, 300),
            reported("L008-S4", 1, 400),
        ];
        let recorded = [
            ("L008-S1", None, 100),
            // The first attempt, interrupted, is not the one reported.
            ("L008-S2", None, 200),
            ("L008-S2", Some(2), 150),
            ("L008-S3", None, 0),
        ];
        assert_eq!(
            short_of(&recorded, &live),
            [
                ("L008-S2".to_string(), 150, 200),
                ("L008-S3".to_string(), 0, 300),
                ("L008-S4".to_string(), 0, 400),
            ]
        );
        assert!(short_of(&[("L008-S1", None, 100)], &live[..1]).is_empty());
    }
}
